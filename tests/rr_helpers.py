"""Driving test registrar nodes (tests/temoto_test_nodes/nodes/rr_node) from pytest."""
import json
import os
import sys

import rospy

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from temoto_test_nodes.srv import Control  # noqa: E402

from temoto_core import control_socket  # noqa: E402
from temoto_testing import wait_for  # noqa: E402

COMMAND_TIMEOUT = 30.0    # generous: a command that hangs fails the test rather than the session


class RegistrarNode:
    """A test registrar process and its ``~control`` service."""

    def __init__(self, procs, name: str, check_period: float = 2.0, control_socket: str = '', **params) -> None:
        """``control_socket``: drive the node through this Unix socket rather than ROS (a node on another
        host: ``temoto_core/hosts.py``)."""
        self.name = name
        self.control_socket = control_socket
        if control_socket:
            params['control_socket'] = control_socket
        self.process = procs.node('temoto_test_nodes', 'rr_node', name=name,
                                  params=dict(params, consumer_check_period=check_period))
        # the control service of this very process: after a restart under the same name the master may
        # still name the dead incarnation's service for a moment
        wait_for(self._answers, 20, 'the control service of %s' % name)

    def _answers(self) -> bool:
        if self.control_socket:
            try:
                self.command(op='counts')
                return True
            except OSError:
                return False
        try:
            rospy.wait_for_service('/%s/control' % self.name, timeout=1.0)
            self.command(op='counts')
            return True
        except (rospy.ROSException, rospy.ServiceException):
            return False

    def command(self, **cmd) -> dict:
        if self.control_socket:
            return control_socket.ask(self.control_socket, cmd, COMMAND_TIMEOUT)
        # a fresh connection per command: each runs in its own service thread, so commands can overlap
        proxy = rospy.ServiceProxy('/%s/control' % self.name, Control)
        return json.loads(proxy(json.dumps(cmd)).result)

    def call(self, rr: str, name: str, params=()) -> dict:
        return self.command(op='call', rr=rr, name=name, params=list(params))

    def unload(self, resource_id: int) -> dict:
        return self.command(op='unload', id=resource_id)

    def fail(self, name: str, message: str = 'failed on purpose') -> dict:
        return self.command(op='fail', name=name, message=message)

    def events(self) -> list:
        return self.command(op='events')['events']

    def owner_events(self) -> list:
        return self.command(op='events')['owner_events']

    def counts(self) -> dict:
        return self.command(op='counts')

    def registry(self) -> dict:
        return self.command(op='registry')['registry']

    def registry_uri(self) -> str:
        """The XML-RPC URI of this node's current incarnation, as the master has it."""
        import rosgraph
        return rosgraph.Master('/rr_helpers').lookupNode('/' + self.name)

    def wait_events(self, count: int, timeout: float = 10.0) -> list:
        return wait_for(lambda: len(self.events()) >= count and self.events(), timeout,
                        '%d status event(s) at %s' % (count, self.name))


def registry_empty(node: RegistrarNode) -> bool:
    reg = node.registry()
    return not reg['server_queries'] and not reg['client_queries']
