"""Driving test registrar nodes (tests/temoto_test_nodes/nodes/rr_node) from pytest."""
import json
import sys
import os

import rospy

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from temoto_test_nodes.srv import Control  # noqa: E402

from temoto_core.testing import wait_for  # noqa: E402


class RegistrarNode:
    """A test registrar process and its ``~control`` service."""

    def __init__(self, procs, name: str, check_period: float = 2.0, **params) -> None:
        self.name = name
        self.process = procs.node('temoto_test_nodes', 'rr_node', name=name,
                                  params=dict(params, consumer_check_period=check_period))
        # the control service of this very process: after a restart under the same name the master may
        # still name the dead incarnation's service for a moment
        wait_for(self._answers, 20, 'the control service of %s' % name)

    def _answers(self) -> bool:
        try:
            rospy.wait_for_service('/%s/control' % self.name, timeout=1.0)
            self.command(op='counts')
            return True
        except (rospy.ROSException, rospy.ServiceException):
            return False

    def command(self, **cmd) -> dict:
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
