"""ROS master look-ups that decide whether a node "really started".

A name registered at the master is not proof: a node that was SIGKILLed never
unregisters, so its stale entry would make a restarted node look ready at once.
So a node counts only when the master knows it *and* the process answering at
its XML-RPC URI reports a pid that belongs to the child we started.
"""
from __future__ import annotations

import http.client
import socket
import urllib.parse
import xmlrpc.client
from typing import Iterable

from temoto_core.xmlrpc_util import proxy

CALLER_ID = '/temoto_master_lookup'
# rospy subscribes to this on a node's first log message (rospy.impl.rosout, get_param_cached)
ROSPY_PARAM_SUBSCRIPTIONS = ('/rosout_disable_topics_generation',)


def _proxy(uri: str, timeout: float) -> xmlrpc.client.ServerProxy:
    return proxy(uri, timeout)


def lookup_node(master_uri: str, node_name: str, timeout: float = 1.0) -> str | None:
    """The node's XML-RPC URI, or None when the master does not know it."""
    code, _msg, uri = _proxy(master_uri, timeout).lookupNode(CALLER_ID, node_name)
    return uri if code == 1 else None


def node_host(master_uri: str, node_name: str, timeout: float = 1.0) -> str | None:
    """The host a node's XML-RPC URI names, or None when the master does not know the node or cannot be asked."""
    try:
        uri = lookup_node(master_uri, node_name, timeout)
    except (OSError, xmlrpc.client.Error, http.client.HTTPException):
        return None
    return urllib.parse.urlparse(uri).hostname if uri else None


def node_pid(node_uri: str, timeout: float = 1.0) -> int | None:
    try:
        code, _msg, pid = _proxy(node_uri, timeout).getPid(CALLER_ID)
    except (OSError, xmlrpc.client.Error, http.client.HTTPException):
        return None                       # stale registration: nobody answers there
    return int(pid) if code == 1 else None


def node_refuses(node_uri: str, timeout: float = 1.0) -> bool:
    """Whether nobody listens at a node's XML-RPC port any more: its kernel refuses the connection, as it does
    at once for a process that died. A port that does not answer in time (a cut link, a stopped node) is not
    taken for a death."""
    try:
        url = urllib.parse.urlsplit(node_uri)
        with socket.create_connection((url.hostname, url.port), timeout):
            return False
    except ConnectionRefusedError:
        return True
    except (OSError, ValueError):
        return False


def parent_pid(pid: int) -> int | None:
    """The parent of ``pid`` from /proc (Linux), or None if it is gone."""
    try:
        with open('/proc/%d/stat' % pid, 'rb') as f:
            stat = f.read().decode(errors='replace')
    except OSError:
        return None
    # the command name (field 2) may contain spaces and parentheses: split after the last ')'
    return int(stat.rsplit(')', 1)[1].split()[1])


def node_is_ours(master_uri: str, node_name: str, pids: Iterable[int], parent: int | None = None,
                 timeout: float = 1.0) -> bool:
    """True when ``node_name`` is registered and its process is one of ``pids`` (or a child of ``parent``)."""
    uri = lookup_node(master_uri, node_name, timeout)
    if uri is None:
        return False
    pid = node_pid(uri, timeout)
    if pid is None:
        return False
    if pid in set(pids):
        return True
    return parent is not None and parent_pid(pid) == parent


def set_params(master_uri: str, clear: Iterable[str], params: dict, timeout: float = 5.0) -> None:
    """Delete the ``clear`` namespaces that exist, then set ``params``, as ``roslaunch`` does (two multicalls).

    Raises RuntimeError naming the parameter the master refused, OSError when it is unreachable."""
    proxy = _proxy(master_uri, timeout)
    canon = sorted({c.rstrip('/') + '/' for c in clear})
    # only the outermost of nested namespaces: deleting /a/ already deleted /a/b/
    outer = [c for c in canon if not any(c != o and c.startswith(o) for o in canon)]
    clear = [c for c in outer if proxy.hasParam(CALLER_ID, c)[2]]
    for names, method, calls in ((clear, 'deleteParam', [(c,) for c in clear]),
                                 (list(params), 'setParam', list(params.items()))):
        if not calls:
            continue
        multi = xmlrpc.client.MultiCall(proxy)
        for call in calls:
            getattr(multi, method)(CALLER_ID, *call)
        for name, (code, msg, _val) in zip(names, multi()):
            if code != 1:
                raise RuntimeError('%s %s: %s' % (method, name, msg))


def registered_nodes(master_uri: str, timeout: float = 1.0) -> set[str]:
    """Every node name that publishes, subscribes or serves something (getSystemState)."""
    code, _msg, state = _proxy(master_uri, timeout).getSystemState(CALLER_ID)
    names: set[str] = set()
    if code == 1:
        for section in state:
            for _topic, nodes in section:
                names.update(nodes)
    return names


def subscriptions_of(master_uri: str, node_name: str, timeout: float = 1.0) -> set[str]:
    """The topics ``node_name`` subscribes to, as the master has them (getSystemState)."""
    code, _msg, state = _proxy(master_uri, timeout).getSystemState(CALLER_ID)
    return {topic for topic, nodes in state[1] if node_name in nodes} if code == 1 else set()


# topics every rospy node may have: they say nothing of which node answers at a URI
COMMON_TOPICS = frozenset(('/rosout', '/clock', '/rosout_agg'))


def _stale(uri: str, node_name: str, publishers: list, subscribers: list, timeout: float) -> bool:
    """Whether the registration of ``node_name`` at ``uri`` is left over from a dead process.

    Nobody answering is the plain case. The other: the dead node's port was reused by another node, which
    answers. It is told apart by what it says it publishes and subscribes to: the topics the master has for
    ``node_name`` (beyond the ones every node has) must all be among them. A node with no such topic cannot be
    told apart, so it counts as alive.
    """
    if node_pid(uri, timeout) is None:
        return True
    expected = {t for t, nodes in publishers + subscribers if node_name in nodes} - COMMON_TOPICS
    if not expected:
        return False
    node = _proxy(uri, timeout)
    try:
        pubs = node.getPublications(CALLER_ID)
        subs = node.getSubscriptions(CALLER_ID)
    except (OSError, xmlrpc.client.Error, http.client.HTTPException):
        return True
    there = {t for t, _type in (pubs[2] if pubs[0] == 1 else []) + (subs[2] if subs[0] == 1 else [])}
    return not expected <= there


def registration_alive(master_uri: str, node_name: str, timeout: float = 1.0) -> bool:
    """Whether ``node_name`` is registered by a live node: not unregistered, and not left over by a dead process
    (:func:`_stale`, which also tells a dead node's port now given to another node)."""
    uri = lookup_node(master_uri, node_name, timeout)
    if uri is None:
        return False
    code, _msg, (publishers, subscribers, _services) = _proxy(master_uri, timeout).getSystemState(CALLER_ID)
    return code == 1 and not _stale(uri, node_name, publishers, subscribers, timeout)


def cleanup_dead_node(master_uri: str, node_name: str, timeout: float = 1.0) -> int:
    """Unregister what a dead node left at the master, as ``rosnode cleanup`` does for one node.

    A node that is SIGKILLed (or crashes) never unregisters, so it stays in ``rosnode list`` and its
    topics look served. Worse, a node started later under the same name makes the master send
    ``shutdown`` to the dead node's URI, and if another node has since been given that port, that node is
    shut down instead. Nothing is touched unless the name is registered *and* the registration is stale
    (:func:`_stale`): a live incarnation under the same name is left alone. Returns how many registrations
    went.
    """
    uri = lookup_node(master_uri, node_name, timeout)
    if uri is None:
        return 0
    master = _proxy(master_uri, timeout)
    code, _msg, (publishers, subscribers, services) = master.getSystemState(CALLER_ID)
    if code != 1 or not _stale(uri, node_name, publishers, subscribers, timeout):
        return 0
    calls = [('unregisterPublisher', topic, uri) for topic, nodes in publishers if node_name in nodes]
    calls += [('unregisterSubscriber', topic, uri) for topic, nodes in subscribers if node_name in nodes]
    for service, nodes in services:
        if node_name in nodes:
            scode, _smsg, service_uri = master.lookupService(CALLER_ID, service)
            if scode == 1:
                calls.append(('unregisterService', service, service_uri))
    multi = xmlrpc.client.MultiCall(master)
    for method, name, api in calls:
        getattr(multi, method)(node_name, name, api)
    # the master forgets a node only once it holds nothing at all, parameter subscriptions included:
    # without this, a dead rospy node that ever logged stays known to lookupNode, also one that
    # unregistered its topics and services itself as it shut down (rospy leaves these)
    for key in ROSPY_PARAM_SUBSCRIPTIONS:
        multi.unsubscribeParam(node_name, uri, key)
    multi()
    return len(calls)
