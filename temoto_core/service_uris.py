"""Where services are, remembered, so that a host cut off from the master still reaches its own nodes.

ROS 1 finds a service through the master before every new connection. With
the robot and the operator's station on two hosts, the master runs on the
robot, so a partition also cuts the station off from the master: the station's
own nodes can no longer find each other's services, and the very calls that
should take a frozen view off the operator's screen (an action asking the
Output Manager, the Output Manager asking its RViz host) fail or hang in
rospy's look-up, which has no timeout.

So every URI the master gives is remembered. While one is known, the master
gets a short bound, and when it cannot be reached the known URI is used. A
service never looked up before is found from a sibling: rospy serves every
service of a node on one port, so ``/ns/node/unload`` lives where
``/ns/node/load`` does. A URI that has gone stale is caught by the connection
itself (refused, or a handshake for a service the node does not have).
"""
from __future__ import annotations

import threading
import time
import xmlrpc.client
from typing import Dict

import rosgraph
import rospy

from temoto_core.xmlrpc_util import proxy as xmlrpc_proxy

# how long the master may take to answer when the URI is known already (a look-up answers in ~1 ms)
MASTER_BOUND_WHEN_KNOWN = 0.3
# how long a plain proxy's look-up may take (rospy's own has no bound)
PROXY_LOOKUP_TIMEOUT = 3.0

_lock = threading.Lock()
_uris: Dict[str, str] = {}


def _node_of(service: str) -> str:
    """The key of the node that serves ``service``, by its name: ``/ns/node`` of ``/ns/node/leaf``."""
    parent = service.rstrip('/').rsplit('/', 1)[0]
    return parent + '/' if parent else ''


def remember(service: str, uri: str) -> None:
    with _lock:
        _uris[service] = uri
        node = _node_of(service)
        if node:
            _uris[node] = uri


def known(service: str) -> str:
    """The URI last given for ``service``, or for a sibling service of the same node; '' if none."""
    node = _node_of(service)
    with _lock:
        return _uris.get(service) or (_uris.get(node, '') if node else '')


def lookup(service: str, deadline: float) -> str:
    """The rosrpc URI of ``service`` within ``deadline`` (a ``time.monotonic()`` instant): from the master,
    or, when the master cannot be reached, the one known; '' if the master does not know the service.
    Raises ``OSError`` if the master cannot be reached in time and no URI is known."""
    cached = known(service)
    left = deadline - time.monotonic()
    bound = min(left, MASTER_BOUND_WHEN_KNOWN) if cached else left
    try:
        master = xmlrpc_proxy(rosgraph.get_master_uri(), max(0.01, bound))
        code, _msg, uri = master.lookupService(rospy.get_name(), service)
    except (OSError, xmlrpc.client.Error):
        if cached:
            return cached
        raise
    if code != 1:
        return ''
    remember(service, uri)
    return uri


class ServiceProxy(rospy.ServiceProxy):
    """rospy's proxy, whose look-up is bounded and falls back on the URI known (see the module's docstring)."""

    def _get_service_uri(self, request) -> str:
        if self.request_class._type != getattr(request, '_type', None):
            raise TypeError('request object type [%s] does not match service type [%s]'
                            % (type(request), self.request_class))
        try:
            uri = lookup(self.resolved_name, time.monotonic() + PROXY_LOOKUP_TIMEOUT)
        except (OSError, xmlrpc.client.Error) as err:
            raise rospy.ServiceException('unable to contact the master to find %s: %s' % (self.resolved_name, err))
        if not uri:
            raise rospy.ServiceException('service [%s] unavailable' % self.resolved_name)
        self.uri = uri
        return uri
